"""An operator in the loop: one command interface (`OperatorCommand`) fed by the robot's remote, a gamepad, the
keyboard, a command script or the scenario, shaped into the MPC's commands (`CommandShaper`) and used by `wbmpc run`
(`run.prepare`) and `wbmpc deploy` (`deploy.DeployOperator`). See docs/operator.md."""

from wbmpc.operator.board import CommandBoard, Posted
from wbmpc.operator.command import OperatorCommand, OperatorLimits
from wbmpc.operator.config import OperatorConfig
from wbmpc.operator.remote import RemoteState, decode_remote, encode_remote
from wbmpc.operator.script import CommandScript, read_script
from wbmpc.operator.session import OperatorSession
from wbmpc.operator.shaper import CommandShaper, RampLimits

__all__ = ["CommandBoard", "Posted", "OperatorCommand", "OperatorLimits", "OperatorConfig", "RemoteState",
           "decode_remote", "encode_remote", "CommandScript", "read_script", "OperatorSession", "CommandShaper",
           "RampLimits"]
