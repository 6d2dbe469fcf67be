"""Maps a 1-D joystick through the learned conditional-autoencoder decoder to Franka joint velocities;
the end-effector baseline."""
