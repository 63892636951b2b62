import numpy as np
import pytest

from wbmpc.robots import load_robot


@pytest.fixture(scope="session")
def b1z1():
    return load_robot("b1_z1")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
