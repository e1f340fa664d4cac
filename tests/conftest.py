from pathlib import Path

import pytest


@pytest.fixture
def test_models() -> Path:
    """Real-world model files shipped with the tests (tests/data, see its README)."""
    return Path(__file__).resolve().parent / "data"
