import sys
from pathlib import Path

# tests import shared helpers (bad_input_cases) from this folder
sys.path.insert(0, str(Path(__file__).parent))
