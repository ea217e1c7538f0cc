"""The simulator: ManiSkill environments with the study's cameras and task readouts (`envs`), the pinhole camera
model and 2D goal projection (`projection`), and robot visuals with decimated meshes for faster CPU rendering
(`lowpoly`). No rule of its own: the demos, frames and evaluation stages build their environments here."""
