"""Command line: one module per subcommand; argument handling, running and reporting only."""
