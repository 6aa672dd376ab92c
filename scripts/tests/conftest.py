"""The benchmark scripts import as they do when run from scripts/ (`from peers import ...`)."""

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
