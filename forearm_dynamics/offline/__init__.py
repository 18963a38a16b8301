"""Offline evaluation of recorded runs (check, score, regression, delivery, the HTML report)."""
