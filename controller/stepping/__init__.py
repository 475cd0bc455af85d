"""The Elegant Stepping model: what the leg learns, and how.

The Kalman-filtered range (:mod:`controller.stepping.range_filter`, filterpy), the range encoder's
non-overlapping cells (:mod:`controller.stepping.encoder`), step-gated short-term memory,
synaptic traces and the reflex-trained weights (:mod:`controller.stepping.learner`), the contact
and lift reflexes (:mod:`controller.stepping.reflexes`), the obstacle-height context and its
learner (:mod:`controller.stepping.height`, :mod:`controller.stepping.context`), the tabular
Q-learning baseline (:mod:`controller.stepping.rl`), the improved learner with the learned lift
(:mod:`controller.stepping.improved`), all behind one protocol
(:mod:`controller.stepping.premotor`); the learned weights on disk
(:mod:`controller.stepping.weights`).

May import: the standard library, numpy, filterpy; never the bus, ``hil`` or ``firmware_sim``.
"""
