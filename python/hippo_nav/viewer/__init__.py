"""Watching a run: a live Rerun viewer and a video of the mapping, both pipeline observers.

```python
from hippo_nav.pipeline import run
from hippo_nav.viewer import RerunObserver, VideoObserver
run("runs/x", stop=40, observers=[VideoObserver("runs/x/mapping.mp4"), RerunObserver("runs/x.rrd")])
```

`RerunObserver` needs the optional extra `pip install 'hippo-nav[viewer]'` (rerun-sdk), imported when one is
made, so `import hippo_nav.viewer` works without it. `VideoObserver` needs only OpenCV. What both show:
docs/viewer.md; the images and geometry they share: `hippo_nav.viewer.panels`.
"""

from hippo_nav.viewer.rerun import RerunObserver
from hippo_nav.viewer.video import VideoObserver

__all__ = ["RerunObserver", "VideoObserver"]
