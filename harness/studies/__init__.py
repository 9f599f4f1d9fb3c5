r'''Studies built on the stages: stability sweeps, the stereo range check, COLMAP self-calibration

    harness.studies.sweep           vary one difficulty, mark where each method breaks
    harness.studies.stereo          the paper's Fig. 12 made quantitative (range error on terrain)
    harness.studies.colmap_selfcal  COLMAP's self-calibration from terrain images

Each runs the public stages of harness.stages (or the terrain renderers) on
plain values and returns a plain result; figures are drawn in reports.
'''
