"""The Neuro-IK Lab in the browser (viser): `python -m app` or `make app`.

Wiring only: it reads from `robots` and `lab` and is never imported by them. Inside, imports go
one way, from the top of this list down (panels/ and tab/ do not import each other):

    __main__.py       `python -m app`: the command line
    server.py         LabApp: the viser server, the shared scene, one TabSession per tab, the render loop
    panels/           the panels every tab shares (server.gui): Train, Views, Runs
    tab/              one browser tab's own scene and controls (client.scene, client.gui)
    training/         the training run every tab shares, without viser: state, live numbers, notebook
    classroom/        who may do what on a shared server: access, limits, uploads, lesson links
    startup.py        the controllers the app opens with (app/pretrained/); `python -m app.startup`
    viser_private.py  every reach into viser's private API
    probe.py          a headless viser client for tests and benchmarks (imports nothing of the app)
"""
