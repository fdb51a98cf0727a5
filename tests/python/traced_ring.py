"""The one ring-shaped object of a contrast image, traced as the extraction traces it: shared by
the tests that check the tracing's building blocks and its bias on independent film frames."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from capsmech.imaging.objects import DETECTION_SMOOTHING_PX, TracedObject, find_objects, trace_object


def traced_ring(contrast: np.ndarray) -> TracedObject:
    """The one object of `contrast` (detection at 6 noise deviations, 30 px at least), which must
    be traced as a ring."""
    smooth = ndimage.gaussian_filter(contrast, DETECTION_SMOOTHING_PX)
    labels, mask, keep, threshold = find_objects(smooth, np.ones(contrast.shape, bool), 6.0, 30)
    assert len(keep) == 1
    traced = trace_object(contrast, labels == keep[0], mask, threshold, smooth)
    assert isinstance(traced, TracedObject) and traced.kind == "ring"
    return traced
