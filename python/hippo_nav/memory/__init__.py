"""Maps that outlive a run: the memory folder every run writes, and reading it back (docs/memory.md).

A run saves what it learnt into `<results>/memory/` (`files.py`): the experience map, the view cells with the
network states they recall, the closure keyframes, where it stopped, and the settings that made them. A later
run starts inside it (`hippo-nav run ... --map PREVIOUS_RESULTS`, or `SlamSystem(..., memory=read_memory(p))`):
lost until a familiar view is confirmed by the closure measurement, then placed in the old map and extending it.
"""

# The package's names are those of `files.py`, listed once there.
from hippo_nav.memory.files import *
from hippo_nav.memory.files import __all__ as __all__
