"""Reading and writing what is on disk: sequence folders, their frames and labels, image readers."""
