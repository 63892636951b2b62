"""Symbolic (CasADi SX) rigid-body dynamics built from a numeric pinocchio model."""

from wbmpc.symbolic.dynamics import Configuration, InertialParameters, Motion, SymbolicDynamics

__all__ = ["Configuration", "InertialParameters", "Motion", "SymbolicDynamics"]
