"""The lasting event log (SQLite in ``<data_dir>``), its recorder and the daily report."""
