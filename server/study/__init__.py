"""The study layer: study files, assignment, the study database, its pages and API, and the data export."""
