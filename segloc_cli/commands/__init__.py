"""The command layer: each command parses its options, calls the pipeline and prints.

One module per command family; ``options.py`` holds what they share.
"""
