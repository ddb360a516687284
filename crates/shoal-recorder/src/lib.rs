//! Shoal's recorder: every Shoal topic into MCAP files, and their replay onto DDS.
