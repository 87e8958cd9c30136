"""The fleet ledger: every printer's job history kept once, its state over time, the
statistics drawn from both, and the figures ``/metrics`` shows."""
