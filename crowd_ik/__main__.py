"""`python -m crowd_ik` runs the command line."""

from crowd_ik.commands.cli import main

raise SystemExit(main())
