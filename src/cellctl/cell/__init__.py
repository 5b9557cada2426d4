"""The cell orchestrator: PackML state machine, cycle steps, alarms, watchdog."""
