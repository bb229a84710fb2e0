"""Layer 6, the ``bimgame`` command line: argument parsing and printing only; the work is done by the
layers below."""
