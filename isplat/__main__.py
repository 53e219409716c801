"""``python -m isplat``: the same as the ``isplat`` command."""

from .cli.main import console

if __name__ == "__main__":
    console()
