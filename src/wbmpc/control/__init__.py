"""Control: the MPC (state + commands -> Solution), interpolation and joint PD."""

from wbmpc.control.commands import Commands
from wbmpc.control.config import CommandLimits, MpcConfig, PushConfig, RecoveryConfig, ReferenceConfig
from wbmpc.control.mpc import MPC
from wbmpc.control.solution import Solution
from wbmpc.control.weights import CostWeights

__all__ = ["MPC", "CommandLimits", "Commands", "CostWeights", "MpcConfig", "PushConfig", "RecoveryConfig",
           "ReferenceConfig", "Solution"]
