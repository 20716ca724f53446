"""Data the product ships, installed as the package ``guardian.data`` (see setup.py).

``highd_sample/``: one generated two-minute HighD-format recording, the default input of
``guardian replay``. Read it through the package (``guardian.highd.replay.default_sample``), never
through the working folder.
"""
