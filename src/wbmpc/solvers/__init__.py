"""Solvers on the stage-wise OCP. Importing this package first puts the fast BLASFEO under Fatrop
and HPIPM where it is installed (`wbmpc setup`) and verified: see `blasfeo.py`."""

from wbmpc.solvers.blasfeo import activate as _activate_fast_blasfeo

_activate_fast_blasfeo()
