"""Motion cueing: the classical washout filter (Reid & Nahon)."""
