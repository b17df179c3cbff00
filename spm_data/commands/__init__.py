"""What each spm-data command does (render, occlude, merge, info, validate, show and hist), one library call each."""
