"""`hubctl timeline` (a recorded run as a Gantt chart) and `hubctl runs` (the recorded runs and their outcome)."""
