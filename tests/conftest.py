from pathlib import Path

import pytest


@pytest.fixture
def shared_models() -> Path:
    """The test models in ../shared/models (next to the repository); skips when absent."""
    p = Path(__file__).resolve().parents[2] / "shared" / "models"
    if not p.is_dir():
        pytest.skip(f"{p} not found")
    return p
