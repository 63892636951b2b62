"""Access to Unitree SDK2 Python (`unitree-sdk2` on PyPI, module `unitree_sdk2py`) and CycloneDDS.

Install: `pip install "cyclonedds>=11" && pip install --no-deps unitree-sdk2` (or `pip install
wbmpc[robot]` then the second command). unitree-sdk2 1.0.1 pins cyclonedds==0.10.2, which has no
wheel and needs a C build of CycloneDDS (CYCLONEDDS_HOME); cyclonedds 11 installs from a wheel and
runs the SDK's channels and IDL types unchanged. The 1.0.1 wheel's top-level `__init__` imports a
`b2` package that is not in the wheel, and its CRC helper loads a `crc_amd64.so` that is not
either: we load the SDK's subpackages without the top-level `__init__` and compute the CRC in
`wbmpc.hardware.crc`. The SDK's channels print their reader errors ("[Reader] take sample error") on
stdout, from DDS threads: they go to stderr here, so that `--json` output stays one JSON object.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from dataclasses import dataclass

from wbmpc.errors import ConfigError

INSTALL_HINT = 'pip install "cyclonedds>=11" && pip install --no-deps unitree-sdk2'


FAMILIES = ("unitree_go", "unitree_hg")  # LowCmd/LowState IDL of quadrupeds / of humanoids (G1, H1-2)


@dataclass(frozen=True)
class Idl:
    """One family's LowState_/LowCmd_ types and constructors of default (zeroed) messages."""

    LowState_: type
    LowCmd_: type
    new_low_state: object
    new_low_cmd: object


@dataclass(frozen=True)
class Sdk:
    """The SDK pieces wbmpc uses (LowState_ ... new_low_cmd: unitree_go's; `idl(family)` for either)."""

    ChannelFactoryInitialize: object
    ChannelPublisher: type
    ChannelSubscriber: type
    LowState_: type
    LowCmd_: type
    new_low_state: object
    new_low_cmd: object
    hg: Idl | None = None

    def idl(self, family: str) -> Idl:
        if family == "unitree_hg":
            if self.hg is None:
                raise ConfigError("this SDK has no unitree_hg messages")
            return self.hg
        if family != "unitree_go":
            raise ConfigError(f"unknown message family {family!r}; available: {', '.join(FAMILIES)}")
        return Idl(self.LowState_, self.LowCmd_, self.new_low_state, self.new_low_cmd)


_SDK: Sdk | None = None


def _print_to_stderr(*args, **kwargs) -> None:
    kwargs["file"] = sys.stderr
    print(*args, **kwargs)


def load_sdk() -> Sdk:
    """Import unitree_sdk2py's channel and IDL modules (once), or a ConfigError saying how to install them."""
    global _SDK
    if _SDK is not None:
        return _SDK
    spec = importlib.util.find_spec("unitree_sdk2py")
    if spec is None or spec.submodule_search_locations is None:
        raise ConfigError(f"the robot interface needs Unitree SDK2 Python and CycloneDDS: {INSTALL_HINT}")
    if "unitree_sdk2py" not in sys.modules:
        package = types.ModuleType("unitree_sdk2py")
        package.__path__ = list(spec.submodule_search_locations)
        package.__spec__ = spec
        sys.modules["unitree_sdk2py"] = package
    try:
        from unitree_sdk2py.core import channel
        from unitree_sdk2py.core.channel import (
            ChannelFactoryInitialize,
            ChannelPublisher,
            ChannelSubscriber,
        )
        from unitree_sdk2py.idl.default import (
            unitree_go_msg_dds__LowCmd_,
            unitree_go_msg_dds__LowState_,
            unitree_hg_msg_dds__LowCmd_,
            unitree_hg_msg_dds__LowState_,
        )
        from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_, LowState_
        from unitree_sdk2py.idl.unitree_hg.msg import dds_ as hg
    except ImportError as exc:
        raise ConfigError(f"Unitree SDK2 Python could not be loaded ({exc}); reinstall it: {INSTALL_HINT}") from None
    channel.print = _print_to_stderr  # the module's own `print` (its reader threads' diagnostics)
    _SDK = Sdk(ChannelFactoryInitialize, ChannelPublisher, ChannelSubscriber, LowState_, LowCmd_,
               unitree_go_msg_dds__LowState_, unitree_go_msg_dds__LowCmd_,
               Idl(hg.LowState_, hg.LowCmd_, unitree_hg_msg_dds__LowState_, unitree_hg_msg_dds__LowCmd_))
    return _SDK
