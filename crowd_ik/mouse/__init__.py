"""`crowd-ik mouse`: one character posed with the mouse, live in a window or replayed to video.

The seeds' interactive demo (homework ik_demo, lab 2, coursework): a planar chain of unit bones
whose tip follows a target. The methods are the planar NumPy ones of :mod:`crowd_ik.planar`
(newton, dls, follow = the lab's residual stepping) and the Taichi solvers of :class:`Crowd`
with N = 1 (fabrik, ccd). The joint angles (homework convention) are the one shared state, so
switching method mid-drag carries the pose over. A target the chain does not reach is "lost"
(drawn white, as in the lab) and the chain stretches toward it.

- live chain: Taichi's GUI window; drag the target; keys 1-5 method, L limits, R reset, C record
  the target path to path_NNN.csv (never overwriting), Esc quit.
- live humanoid (--rig humanoid): drag a hand, foot or head in the camera's view plane; FABRIK,
  DLS or CCD on the whole body, the other effectors held.
- replay: --path PATH.csv (t,x,y per row) or --keyframes FILE.csv (eased key poses) to a video.

Modules: session (the chain's state and step), paths (target path CSVs, recording), replay (to
video), live (the windows), view (drawing); the command is crowd_ik/commands/mouse.py.
"""
