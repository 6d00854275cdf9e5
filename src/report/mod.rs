//! Reports: JSON, SVG figures and Markdown.
