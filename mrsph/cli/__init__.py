"""The command line (``python3 main.py``, the ``mrsph`` command): the commands and their
options (``commands.py``, ``options.py``) and the benchmark (``bench/``). ``main`` is
resolved on first use, so that importing ``mrsph.cli.options`` stays light."""

__all__ = ["main"]


def __getattr__(name: str):
    if name == "main":
        from .commands import main
        return main
    raise AttributeError(f"module 'mrsph.cli' has no attribute {name!r}")
