"""Planning: reference paths from recorded drives, progress along them, and their speed profiles."""
