"""Run recordings: every run's states, commands, plans, operation transitions, requests and watchdog
verdicts in one SQLite file (schema.py), written off the controller's loop (writer.py), read by
timeline, `hubctl runs` and `hubctl replay` (reader.py)."""
