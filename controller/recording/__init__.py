"""Run recordings: every run's states, commands, plans, operation transitions, requests and watchdog
verdicts in one SQLite file (schema.py), handed off by the controller's thread (writer.py) through a
pipe (wire.py) to a process that stores them (writer_process.py, store.py), read by timeline,
`hubctl runs` and `hubctl replay` (reader.py)."""
