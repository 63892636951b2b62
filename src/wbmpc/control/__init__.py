"""Control: the MPC (state + commands -> Solution), interpolation and joint PD."""

from wbmpc.control.mpc import MPC, Commands, CostWeights, MpcConfig
from wbmpc.control.solution import Solution

__all__ = ["MPC", "Commands", "CostWeights", "MpcConfig", "Solution"]
