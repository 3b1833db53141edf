"""Station projects from a resource model: `hubctl new-station` and `hubctl new-device` (docs/new-station.md).

`station` writes a project skeleton, `device` a driver skeleton with its variable
contract and model-based test, `files` the templates (templates/) and the edits,
`testing` the pytest fixtures the generated tests use, `cli` the two commands.
"""
