"""One browser tab's own scene and controls (client.scene, client.gui): goals, arms, IK ghosts, population, replay."""
