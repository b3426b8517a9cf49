//! Detector networks and inference (filled by the detectors issue).
