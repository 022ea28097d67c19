"""Builds the optional compiled hot loops with Cython: the route (entitynet/switchboard/_fanout.pyx) over the
outboxes in C arrays (entitynet/switchboard/_outbox.pyx, with its .pxd), the flush loop
(entitynet/server/_flushloop.pyx), the read hub's per-read path (entitynet/server/_hubpass.pyx) and the client
state's field accessors (entitynet/client/_columns.pyx), the lateral cover's candidate loop
(entitynet/client/_lateral.pyx, and over C tables _waytable.pyx), the payload's quantisation
(entitynet/client/_payload.pyx), `Path.xy` (entitynet/client/_geom.pyx), the cell occupation
(entitynet/client/_occupy.pyx; the network model's publish cover around it, _cover.pyx), the fleet core's kernels
(entitynet/client/_fleet.pyx), the codec's PUBLISH loop (entitynet/protocol/_decode.pyx) and the ghost table's
per-message queue (entitynet/client/_ghost_queue.pyx), and the simulation's viewer frame walk
(sims/engine/_frame_walk.pyx); everything else is in pyproject.toml. Optional on purpose:
without a C compiler the build goes on and the pure-Python paths (the references, `entitynet.switchboard.outbox`,
`entitynet.server.flushloop` and `entitynet.server.hubpass`, `entitynet.client.state.column`, the codec's
`_decode_one`, `sims.engine.message_cache`'s Python walk) are used."""

from setuptools import Extension, setup

try:
    from Cython.Build import cythonize
except ImportError:  # no Cython at build time: the pure path only
    ext_modules = []
else:
    ext_modules = cythonize(
        [Extension("entitynet.switchboard._fanout", ["entitynet/switchboard/_fanout.pyx"], optional=True),
         Extension("entitynet.switchboard._outbox", ["entitynet/switchboard/_outbox.pyx"], optional=True),
         Extension("entitynet.server._flushloop", ["entitynet/server/_flushloop.pyx"], optional=True),
         Extension("entitynet.server._hubpass", ["entitynet/server/_hubpass.pyx"], optional=True),
         Extension("entitynet.client._columns", ["entitynet/client/_columns.pyx"], optional=True),
         Extension("entitynet.client._lateral", ["entitynet/client/_lateral.pyx"], optional=True),
         Extension("entitynet.client._waytable", ["entitynet/client/_waytable.pyx"], optional=True),
         Extension("entitynet.client._payload", ["entitynet/client/_payload.pyx"], optional=True),
         Extension("entitynet.client._geom", ["entitynet/client/_geom.pyx"], optional=True),
         Extension("entitynet.client._occupy", ["entitynet/client/_occupy.pyx"], optional=True),
         Extension("entitynet.client._cover", ["entitynet/client/_cover.pyx"], optional=True),
         Extension("entitynet.client._fleet", ["entitynet/client/_fleet.pyx"], optional=True),
         Extension("entitynet.protocol._decode", ["entitynet/protocol/_decode.pyx"], optional=True),
         Extension("entitynet.client._ghost_queue", ["entitynet/client/_ghost_queue.pyx"], optional=True),
         Extension("sims.engine._frame_walk", ["sims/engine/_frame_walk.pyx"], optional=True)],
        language_level=3,
        quiet=True,
    )
    for ext in ext_modules:  # cythonize makes new Extension objects and drops `optional`: without it a missing
        ext.optional = True  # C compiler fails the whole install instead of leaving the pure-Python paths

setup(ext_modules=ext_modules)
