"""Offline interactive 3-D viewer: prediction vs ground truth of a scan in one HTML file.

- :mod:`~panoptic_bench.viewer.matching`: per-segment TP / FP / FN with the evaluator's rules;
- :mod:`~panoptic_bench.viewer.scene`: the scan and class facts shown;
- :mod:`~panoptic_bench.viewer.load`: scans from SemanticKITTI trees and nuScenes dataroots;
- :mod:`~panoptic_bench.viewer.payload` and :mod:`~panoptic_bench.viewer.page`: the page;
- :mod:`~panoptic_bench.viewer.report`: viewer pages of report sets (best and worst scan by PQ).
"""
