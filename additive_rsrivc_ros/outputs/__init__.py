"""What users read: reports, figures, verdicts, fleet reports and the status text."""
