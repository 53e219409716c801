"""setuptools reads pyproject.toml; this only tags a wheel that holds the prebuilt kernels for its platform.

The kernels prebuilt by ``make prebuilt`` (isplat/_prebuilt, isplat.prebuilt) are x86-64 machine code for one
Python version, so a wheel that holds them is not pure Python: it is tagged for this interpreter and platform
(for example ``cp311-cp311-linux_x86_64``) rather than ``py3-none-any``. Without them the wheel stays pure.
"""

import os

from setuptools import setup
from setuptools.dist import Distribution


class _Distribution(Distribution):
    def has_ext_modules(self):
        return os.path.exists(os.path.join(os.path.dirname(os.path.abspath(__file__)), "isplat", "_prebuilt",
                                           "manifest.json"))


setup(distclass=_Distribution)
