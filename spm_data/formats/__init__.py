"""Other datasets' formats, in and out: COIL-100, CVL and posed folders, BOP (with PLY models and COCO ground truth)."""
