"""Fault injection: what goes wrong on a real bus, done on purpose, and what the stack did.

One seeded fault model per frame (drop, delay, duplicate, reorder, corrupt) and the faulty buses
built on it (:mod:`hil.faults.model`); a man-in-the-middle node between two SocketCAN channels
(:mod:`hil.faults.mitm`); the fault side of a HIL session: kill -9 of the controller, a silenced
node (:mod:`hil.faults.session`); kill -9 during weight saves (:mod:`hil.faults.killsave`); the one
audit of the commands sent (:mod:`hil.faults.audit`); the fault matrix (:mod:`hil.faults.matrix`).

May import: ``controller``, ``firmware_sim``, ``protocol``, and the harness's lockstep, session,
experiments and analysis packages.
"""
