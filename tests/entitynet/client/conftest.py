import sys
from pathlib import Path

# client_fixtures lives one level up (tests/entitynet/), shared with other client-side tests
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
