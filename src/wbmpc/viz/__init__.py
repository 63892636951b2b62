"""Visualisation of closed-loop runs: diagnostic PNG plots and a self-contained HTML 3D replay."""

from wbmpc.viz.plots import base_velocity_heading, frame_positions, save_plots
from wbmpc.viz.replay import replay_data, save_replay

__all__ = ["base_velocity_heading", "frame_positions", "replay_data", "save_plots", "save_replay"]
