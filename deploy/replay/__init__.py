"""`hubctl replay`: a recorded run's inputs fed to a fresh controller core, its decisions compared."""
