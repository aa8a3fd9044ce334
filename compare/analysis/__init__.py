"""What a run produced, measured and shown: metrics, ISO/TS 15066 margin, results files, reports, plots."""
