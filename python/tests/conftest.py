"""Shared fixtures of the Python tests: where the build and the source tree are, and small volumes."""
import os

import numpy as np
import pytest

SOURCE_DIR = os.environ.get("CIP_SOURCE_DIR", os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..")))
BINARY_DIR = os.environ.get("CIP_BINARY_DIR", os.path.join(SOURCE_DIR, "build"))


@pytest.fixture
def extract_exe():
    return os.path.join(BINARY_DIR, "extract", "extract")


@pytest.fixture
def raycast_exe():
    return os.path.join(BINARY_DIR, "raycast", "raycast")


@pytest.fixture
def blobs_path():
    return os.path.join(SOURCE_DIR, "data", "blobs.nrrd")


def grid(shape=(41, 33, 29)):
    return np.mgrid[-1:1:complex(shape[0]), -1:1:complex(shape[1]), -1:1:complex(shape[2])]


def sphere(shape=(41, 33, 29)):
    x, y, z = grid(shape)
    return x * x + y * y + z * z


def gyroid(shape=(41, 33, 29), k=4.0):
    x, y, z = grid(shape)
    return np.sin(k * x) * np.cos(k * y) + np.sin(k * y) * np.cos(k * z) + np.sin(k * z) * np.cos(k * x)
