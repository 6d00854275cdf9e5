fn main() {
    std::process::exit(osim_spine::cli::main());
}
