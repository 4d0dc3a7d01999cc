"""The simulated world: one MuJoCo model holding walls and every body in it."""
