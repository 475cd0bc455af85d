"""User-Mode Linux: a Linux kernel with SocketCAN, booted as an ordinary process.

:mod:`hil.uml.runner` decides where vcan can be had (natively, else inside UML), boots the VM with
this folder's init script and runs a command inside it; the folder also ships the assets
(``run-in-uml.sh``, ``uml-init``, ``install.sh`` and two small C preload shims).

May import: the standard library and python-can only (it runs before anything else is known).
"""
