"""The harness around the controller: everything that is not deployed to the leg.

One sub-package per role: :mod:`hil.lockstep` (controller and simulated leg in one process, one
bus, stepped together: tests and fast experiments); :mod:`hil.session` (the two as separate
processes on a real SocketCAN bus) and :mod:`hil.uml` (User-Mode Linux, which gives a kernel with
CAN where this one has none); :mod:`hil.faults` (fault injection and the fault matrix);
:mod:`hil.experiments` (walk, learn, sweep, the method registry); :mod:`hil.analysis` (metrics,
statistics, figures, reports, replay); :mod:`hil.bench` (performance against the physics alone);
:mod:`hil.dryrun` (the systemd unit played against the simulated leg); :mod:`hil.envs` (Gymnasium
environments of the leg's tasks, for reinforcement-learning libraries); :mod:`hil.cli` (the
``elegant-stepping`` command line, one module per verb). :mod:`hil.profile` holds every timing
allowance that differs between a native kernel and User-Mode Linux.

May import everything: ``controller``, ``firmware_sim``, ``protocol``, ``urdf``, and the ``sim``
and ``research`` extras (pybullet; matplotlib, tqdm, dask, gymnasium), the latter inside the functions that
need them. It is the only package that sees both sides of the bus; nothing imports it.
"""

# first, before any hot module: ELEGANT_STEPPING_PURE_PYTHON=1 runs them as pure Python (protocol.compiled)
from protocol.compiled import install_pure_python_finder as _install_pure_python_finder

_install_pure_python_finder()
