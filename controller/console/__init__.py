"""The operator console (`hubctl console`): a terminal UI that watches and steers the controller.

`app` is the Textual application and `run_console`; `link` its side of the bus (status,
state, self-test reports, requests); `station` what it knows from hubs.toml and the model
before the controller says anything; `view` the panels as rows of text and the event feed;
`table` the tables that redraw only the cells that changed. Only `app` needs a terminal.
"""
