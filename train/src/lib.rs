//! Training (filled by the detectors issue).
