"""The command line explains itself: help for every option, errors that name the fix."""
