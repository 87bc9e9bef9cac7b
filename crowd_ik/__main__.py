"""`python -m crowd_ik` runs the command line."""

from crowd_ik.cli import main

raise SystemExit(main())
