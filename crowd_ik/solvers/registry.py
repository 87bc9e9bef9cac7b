"""The IK methods a Crowd solves with: their names, defined once.

Every product module that names a method (the Crowd, the scene schema, the command line, the bench, the
mouse demo, the chart) imports it from here; tests/test_layering.py checks that no other product module
spells a method name as a string literal. A new solver gets its name here, an adapter
crowd_ik/solvers/<name>.py (`solve(crowd, request)`, listed in crowd.SOLVERS), its kernels in kernels/
and its NumPy twin in crowd_ik/reference/<name>.py.
"""

FABRIK = "fabrik"  # Aristidou & Lasenby 2011, with joint limits and sub-bases (kernels/fabrik*.py)
DLS = "dls"        # damped least squares, LM damping, joint-limit active set (kernels/dls*.py)
CCD = "ccd"        # cyclic coordinate descent (kernels/ccd.py)

METHODS = (FABRIK, DLS, CCD)
DEFAULT = FABRIK

# The planar mouse demo's methods, keys 1-5: two of the course's NumPy solvers (crowd_ik/planar.py) beside
# the crowd's own; DLS there is planar.dls, FABRIK and CCD a Crowd of one.
NEWTON, FOLLOW = "newton", "follow"
PLANAR_METHODS = (NEWTON, DLS, FABRIK, CCD, FOLLOW)
PLANAR_DEFAULT = DLS
