"""Symbolic (CasADi SX) rigid-body dynamics built from a numeric pinocchio model."""

from wbmpc.symbolic.dynamics import Configuration, Motion, SymbolicDynamics

__all__ = ["Configuration", "Motion", "SymbolicDynamics"]
