"""The simulated world: MuJoCo scene and Panda simulator, its clock, camera renderer and the scripted
push planner.
"""
