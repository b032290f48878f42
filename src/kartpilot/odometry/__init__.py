"""Visual odometry (stereo, and monocular with the ground plane's scale), place recognition, and the localisers
that turn them into the kart's pose on the road."""
