"""The command layer: each command parses its options, calls the pipeline and prints.

One module per command family (``localize`` with ``localize_lines``, what it prints;
``evaluate``; ``maps`` and ``plans``; ``logs`` and ``imports``; ``info``; ``sweep``;
``emulate``; ``record``). What they share: ``options`` (the option decorators and their
click types), ``configfile`` (``--config``), ``invocation`` (what a command was asked, and
its run file), ``optionvalues`` (option text parsed into values) and ``printing`` (what a
command prints besides its errors).
"""
