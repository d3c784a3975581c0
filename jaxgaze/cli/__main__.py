"""``python -m jaxgaze.cli``: the ``jaxgaze`` command."""

from jaxgaze.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
