"""wbmpc: whole-body inverse-dynamics MPC for legged loco-manipulation."""

__version__ = "0.1.0"
