"""Visual odometry: frame-to-frame motion from stereo (and later monocular) images."""
