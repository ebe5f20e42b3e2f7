"""Skill-assessment metrics of tip trajectories (pure numpy): the motion-analysis figures surgical
educators use, per segment, with intervals from the estimate's own uncertainty. `kinematics`
holds the path, fulcrum, volume and movement quantities, `smoothness` SPARC and LDLJ, `assess`
one segment's figures and their intervals."""
