"""Maps a 1-D joystick through the learned conditional-autoencoder decoder to Panda joint
velocities; end-effector baseline; simulated teleoperator."""
