"""What spm train, spm evaluate and spm predict call: one library function each."""
