"""The ``kartpilot`` command line: thin subcommands over library functions."""
