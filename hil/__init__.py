"""The harness that joins the controller and the simulated leg.

In-process lockstep over python-can's ``virtual`` bus (:mod:`hil.lockstep`, for tests and fast
experiments), experiments and their JSON (:mod:`hil.walk`), benchmarks (:mod:`hil.bench`),
fault injection on the bus (:mod:`hil.faults`) and the ``elegant-stepping`` command line
(:mod:`hil.cli`).

May import everything: ``controller``, ``firmware_sim``, ``protocol``, ``urdf``. It is the only
package that sees both sides of the bus.
"""
