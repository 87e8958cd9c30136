"""The fleet job queue: jobs dispatched to compatible idle printers, only onto a cleared plate."""
