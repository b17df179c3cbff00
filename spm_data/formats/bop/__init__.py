"""BOP (Hodaň et al.), in and out, each file's reader beside its writer (as bop_toolkit's inout.py):

- read.py: a BOP dataset in (``spm-data import bop``; scene files by scene.py's ``load_scene_file``);
- export.py: our shards out (``spm-data export bop``), driving scene.py (``SceneWriter``, the
  scene files ``save_scene_file`` / ``load_scene_file``), gt.py (ground truth by bop_toolkit's
  rules), models.py (``models/``, ``models_eval/``, ``save_models_info`` / ``load_models_info``)
  and ids.py (object, scene and image ids; ``objects.json``: ``save_objects`` / ``load_objects``);
- results.py: pose estimates as BOP results files and the targets file (``save_bop_results`` /
  ``load_bop_results``, ``save_test_targets`` / ``load_test_targets``).

Import from the module that holds a thing: nothing is re-exported here.
"""
