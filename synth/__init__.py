"""Domain-randomised MuJoCo renders of URDF arms, written in the DREAM layout (issue 3)."""
