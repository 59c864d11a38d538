"""The report of a reproduction, in separate modules:

- `records`: typed records of one run, per-variant summaries, tests and claim verdicts;
- `statistics`: summaries over seeds, Welch tests, comparisons and the claims' verdicts;
- `context`: the machine and the datasets a report describes;
- `figures`: bar, size-study and scene figures, and `save` (atomic);
- `markdown`: the text of RESULTS.md;
- `document`: `write_report`, which joins them into RESULTS.md, results.json and results/.
"""
