"""Builds the optional compiled fan-out (entitynet/switchboard/_fanout.pyx) with Cython; everything else is in
pyproject.toml. Optional on purpose: without a C compiler the build goes on and the pure-Python path (the
reference, `entitynet.switchboard.outbox`) is used."""

from setuptools import Extension, setup

try:
    from Cython.Build import cythonize
except ImportError:  # no Cython at build time: the pure path only
    ext_modules = []
else:
    ext_modules = cythonize(
        [Extension("entitynet.switchboard._fanout", ["entitynet/switchboard/_fanout.pyx"], optional=True)],
        language_level=3,
        quiet=True,
    )

setup(ext_modules=ext_modules)
