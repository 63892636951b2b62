"""Network interface checks before DDS starts (CycloneDDS binds to the named interface only)."""

from __future__ import annotations

import socket

from wbmpc.errors import ConfigError


def check_interface(name: str) -> str:
    """`name` if this machine has that interface, else a ConfigError listing the interfaces."""
    names = [n for _, n in socket.if_nameindex()]
    if name not in names:
        raise ConfigError(f"unknown network interface '{name}'; this machine has: {', '.join(names)} "
                          "(use lo for robot-sim on this machine, the robot's interface otherwise)")
    return name
