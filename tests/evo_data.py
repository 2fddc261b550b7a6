"""Real ground-truth files from evo's source package on PyPI (GPL-3.0, so fetched, never vendored).

evo's sdist holds TUM RGB-D freiburg1_xyz's and EuRoC V1_02's ground truth under ``test/data``. The
archive is downloaded once (pinned by version and SHA-256) into ``$LOSSVO_TEST_CACHE`` (default
``~/.cache/lossvo-tests``) and the files are read from it.
"""

from __future__ import annotations

import hashlib
import os
import tarfile
import urllib.request
from pathlib import Path

from filelock import FileLock

EVO_SDIST = (
    "https://files.pythonhosted.org/packages/46/ec/c1d4bab73a27f3c9ab6bb24de35d88db565e4e4e2ebdf79167110610b736/"
    "evo-1.38.1.tar.gz"
)
EVO_SHA256 = "1d63faeeb37604641db65bdd08b0e83e71884071de368058a9c45bdcac3fc3f7"
TUM_FR1_XYZ = "freiburg1_xyz-groundtruth.txt"
EUROC_V102 = "V102_groundtruth.csv"


def _cache() -> Path:
    return Path(os.environ.get("LOSSVO_TEST_CACHE", Path.home() / ".cache" / "lossvo-tests")).expanduser()


def evo_file(name: str) -> Path:
    """The path of ``test/data/<name>`` from evo's sdist, downloading and unpacking it on first use."""
    folder = _cache() / "evo-1.38.1"
    target = folder / name
    folder.mkdir(parents=True, exist_ok=True)
    with FileLock(str(folder) + ".lock"):
        if not target.is_file():
            archive = folder / "evo-1.38.1.tar.gz"
            if not archive.is_file():
                partial = archive.with_suffix(".part")
                urllib.request.urlretrieve(EVO_SDIST, partial)
                digest = hashlib.sha256(partial.read_bytes()).hexdigest()
                if digest != EVO_SHA256:
                    raise RuntimeError(f"{EVO_SDIST}: SHA-256 {digest}, expected {EVO_SHA256}")
                partial.replace(archive)
            with tarfile.open(archive) as tar:
                for member in (TUM_FR1_XYZ, EUROC_V102):
                    data = tar.extractfile(f"evo-1.38.1/test/data/{member}")
                    assert data is not None
                    (folder / member).write_bytes(data.read())
    return target
