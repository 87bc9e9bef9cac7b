"""Host geometry the product needs: quaternions, forward kinematics, the counter-based RNG, swept capsules (NumPy).

The NumPy twins in crowd_ik/reference/ build on these; the kernels have their own Taichi versions,
tested against these."""
