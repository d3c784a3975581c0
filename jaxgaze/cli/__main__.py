"""``python -m jaxgaze.cli``: the ``jaxgaze`` command."""

from jaxgaze.cli import console_main

if __name__ == "__main__":
    console_main()
