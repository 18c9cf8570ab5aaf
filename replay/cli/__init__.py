"""The ``atikt-replay`` command line: one subcommand registry, inspect, learn and view commands."""
