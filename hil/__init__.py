"""The harness that joins the controller and the simulated leg.

In-process lockstep over python-can's ``virtual`` bus (:mod:`hil.lockstep`, for tests and fast
experiments); the learning experiment (:mod:`hil.learn`), its baselines (:mod:`hil.methods`,
:mod:`hil.oracle`), sweeps on a process pool or Dask (:mod:`hil.sweep`, :mod:`hil.report`),
analysis and figures (:mod:`hil.analysis`, :mod:`hil.figures`, :mod:`hil.animation`);
hardware-in-the-loop over SocketCAN, inside User-Mode Linux where the kernel has no CAN
(:mod:`hil.hilrun`, :mod:`hil.uml`, :mod:`hil.replay`); the controller daemon and its periodic
weight saves (:mod:`hil.controller_proc`, :mod:`hil.autosave`), its systemd notifications
(:mod:`hil.sdnotify`, :mod:`hil.daemon_notify`) and the deployment dry run that plays systemd
(:mod:`hil.dryrun`, :mod:`hil.notify_listener`, :mod:`hil.unitfile`); the bring-up command
(:mod:`hil.bringup_cli`); the fault matrix (:mod:`hil.faultmatrix`); benchmarks (:mod:`hil.bench`,
:mod:`hil.bench_hil`); fault injection on the bus (:mod:`hil.faults`), in HIL sessions (the
man-in-the-middle node :mod:`hil.mitm`, kill -9 and silence events :mod:`hil.hilfaults`, the
leg's heartbeats :mod:`hil.legwatch`) and during weight saves (:mod:`hil.killsave`) and the
``elegant-stepping`` command line (:mod:`hil.cli`).

May import everything: ``controller``, ``firmware_sim``, ``protocol``, ``urdf``. It is the only
package that sees both sides of the bus.
"""
