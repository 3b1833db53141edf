"""Stations whose devices' timing matters: a plan is only as good as the devices' ability to follow it."""
