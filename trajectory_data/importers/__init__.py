"""Importers of public trajectory data sets into the dataset format (`trajectory_data.format`).

Each importer reads the files as distributed (numpy only), cuts them into the windows of the
data set's usual protocol and writes schema-2 files atomically (`common.write_all`). Malformed
input raises `common.ImportDataError`, one line naming the file and the line; nothing is
written then. `tools/import_data.py` is the command line.
"""
