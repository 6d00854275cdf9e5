//! OpenSim document I/O: a lossless XML tree of the .osim file, typed views of
//! the components the tool works on, and the upgrade of 2.x/3.x documents.
