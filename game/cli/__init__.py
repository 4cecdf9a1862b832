"""The `chainsim` command line: the entry point and one module per subcommand in `commands/`."""
