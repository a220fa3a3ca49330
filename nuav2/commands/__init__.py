"""CLI sub-commands: each module here defines ``register(subparsers)``; ``nuav2.cli`` finds them.

A module registers one top-level command (e.g. ``demo``) or adds to a shared group such as
``convert`` / ``bench`` through :func:`nuav2.cli.group`.
"""
