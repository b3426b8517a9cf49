//! Localization (filled by the localization issue).
