"""The fleet: end of line, drift and revalidation, the fleet summary's pages."""
