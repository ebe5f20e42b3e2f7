"""The bench study: accuracy against the bench's ground truth, the static protocols, ablations and
the paper report (`tiplog evaluate`). It reads truth the product never sees, and is not part of
the OR image."""
