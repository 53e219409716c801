"""The ``isplat`` command-line suite: one module per subcommand, loaded only when used."""
