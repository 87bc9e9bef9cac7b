"""Taichi kernels of crowd_ik (installed as crowd_ik.kernels): ndarray arguments, no state, no I/O."""
