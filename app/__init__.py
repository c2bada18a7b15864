"""The Neuro-IK Lab in the browser (viser): `python -m app` or `make app`.

Wiring only: it reads from `robots` and `lab` and is never imported by them.
See app/server.py for the layout (shared scene and panels, one TabSession per tab, render loop).
"""
