"""``python -m isplat``: the same as the ``isplat`` command."""

from .cli.main import main

if __name__ == "__main__":
    main()
