"""The command line of both programs (spm-data, spm): click commands, one library call each."""
