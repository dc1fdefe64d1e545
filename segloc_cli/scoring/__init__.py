"""Scoring estimates against the truth: Table 1, relation errors, figures. Pure: files
are read and written by ``io`` and the commands."""
