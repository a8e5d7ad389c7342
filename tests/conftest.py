import sys
from pathlib import Path

import pytest

# tests import shared helpers (bad_input_cases) from this folder
sys.path.insert(0, str(Path(__file__).parent))

TOY_BUILD_STEPS = 500  # the quick preset; enough for the toy targets of test_end_to_end (docs/benchmarks.md)


@pytest.fixture(scope="session")
def toy_build(tmp_path_factory):
    """The toy two-box scene built once per session with the quick preset (shared by
    test_end_to_end.py and test_examples.py): a BuildResult; the scene is ``out_dir.parent / "scene"``."""
    from scenelabel import build, preset, write_toy_scene

    root = tmp_path_factory.mktemp("toy")
    scene = write_toy_scene(root / "scene")
    config = preset("quick", {"train": {"steps": TOY_BUILD_STEPS}})
    return build(scene, root / "out", config, progress=False)


@pytest.fixture(scope="session")
def client():
    """A 2-worker local Dask cluster (processes, one thread each, as ``--workers 2`` starts),
    shared by the cluster tests of test_batch.py and test_map_export.py."""
    from distributed import Client, LocalCluster

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        Client(cluster) as dask_client,
    ):
        yield dask_client
