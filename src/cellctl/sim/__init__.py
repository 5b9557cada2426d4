"""The digital twin: a simulated cell that knows the truth."""
