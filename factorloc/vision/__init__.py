"""Vision helpers of the camera steps: queries resampled onto the reference panorama's grid,
keypoints with azimuths, and wrap-around normalized cross-correlation."""
