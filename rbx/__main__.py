"""``python -m rbx``: the command line (the same as ``rbx``)."""
from .cli.main import main

if __name__ == "__main__":
    main()
