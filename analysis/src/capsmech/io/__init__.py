"""Input and output: measurement CSVs, contour files, kernel case files and database files."""
