"""``grassd studio``: the paper's interactive virtual environment in a browser.

``inputs`` (what a person sets: the light, the eye, the pixel, the tables, each checked),
``lights`` (where the light comes from: an HDRI file, the daemon's bundles, an upload),
``session`` and ``views`` (what is computed from them: the characteristic refined round by
round, the pixel's image, the table, the display showing a picture, the contrast left, the
condition pinned beside it), ``pace`` (how much work each step takes, for the latency goals),
``worker`` (the thread that runs the renderer's jobs in order, a page's newer request
superseding its older one), ``superseding`` (how a newer request stops the launch in flight),
``process`` (the simulator process that thread lives in, and the messages it exchanges with
the server), ``server`` (the aiohttp app: the page, its JSON API and the WebSocket that streams
the views as they refine) and ``messages`` (what the page is sent: its state, the uploads'
answers, the streamed views).
"""
