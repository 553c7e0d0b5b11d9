//! [`StudyQuery`]: the keys of a QIDO-RS study search, checked before they
//! are sent (DICOM PS3.18 §8.3.4: attribute matching, `limit`, `offset`).

/// Most characters of a matching value (LO and PN components hold 64).
pub const MAX_VALUE_CHARS: usize = 64;
/// Most results one search asks for.
pub const MAX_LIMIT: u32 = 1000;
/// Results a search asks for when not told.
pub const DEFAULT_LIMIT: u32 = 100;

/// A StudyDate match: one day, or a range open at either end (`YYYYMMDD`,
/// `YYYYMMDD-YYYYMMDD`, `-YYYYMMDD`, `YYYYMMDD-`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DateRange {
    /// The first day, if bounded below.
    pub from: Option<u32>,
    /// The last day, if bounded above.
    pub to: Option<u32>,
}

impl DateRange {
    /// Parses a DICOM date range.
    pub fn parse(text: &str) -> Result<DateRange, String> {
        let expected =
            "expected YYYYMMDD or a range YYYYMMDD-YYYYMMDD (either end may be left out)";
        let day = |d: &str| -> Result<Option<u32>, String> {
            if d.is_empty() {
                return Ok(None);
            }
            let valid = d.len() == 8 && d.bytes().all(|b| b.is_ascii_digit());
            let n: u32 = if valid { d.parse().unwrap_or(0) } else { 0 };
            let (month, day) = (n / 100 % 100, n % 100);
            if !valid || !(1..=12).contains(&month) || !(1..=31).contains(&day) {
                return Err(format!(
                    "StudyDate {text:?}: {d:?} is not a date; {expected}"
                ));
            }
            Ok(Some(n))
        };
        let range = match text.split_once('-') {
            Some((from, to)) => DateRange {
                from: day(from)?,
                to: day(to)?,
            },
            None => {
                let d = day(text)?;
                DateRange { from: d, to: d }
            }
        };
        match range {
            DateRange {
                from: None,
                to: None,
            } => Err(format!("StudyDate {text:?}: no date; {expected}")),
            DateRange {
                from: Some(a),
                to: Some(b),
            } if a > b => Err(format!(
                "StudyDate {text:?}: the range ends before it begins"
            )),
            r => Ok(r),
        }
    }

    /// As QIDO-RS takes it.
    pub fn to_query(self) -> String {
        let day = |d: Option<u32>| d.map(|d| format!("{d:08}")).unwrap_or_default();
        if self.from == self.to {
            return day(self.from);
        }
        format!("{}-{}", day(self.from), day(self.to))
    }
}

/// The keys of a study search; `None` matches anything.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StudyQuery {
    /// PatientName (wildcards `*` and `?`).
    pub patient_name: Option<String>,
    /// PatientID (wildcards `*` and `?`).
    pub patient_id: Option<String>,
    /// AccessionNumber.
    pub accession_number: Option<String>,
    /// StudyDate.
    pub study_date: Option<DateRange>,
    /// ModalitiesInStudy (e.g. `CT`).
    pub modality: Option<String>,
    /// StudyInstanceUID.
    pub study_uid: Option<String>,
    /// Results to return at most (1 to [`MAX_LIMIT`]; [`DEFAULT_LIMIT`] when 0).
    pub limit: u32,
    /// Results to pass over first.
    pub offset: u32,
}

/// A matching value: 1 to [`MAX_VALUE_CHARS`] characters, none a control
/// character or a backslash (DICOM's value separator).
pub fn check_value(key: &str, value: &str) -> Result<String, String> {
    let value = value.trim();
    if value.is_empty()
        || value.chars().count() > MAX_VALUE_CHARS
        || value.chars().any(|c| c.is_control() || c == '\\')
    {
        return Err(format!(
            "{key} {value:?}: expected 1 to {MAX_VALUE_CHARS} characters without control characters or backslashes"
        ));
    }
    Ok(value.to_owned())
}

/// A UID ([`blocks::ingest::dicom::is_uid`]): numbers joined by dots, at
/// most 64 characters.
pub fn check_uid(key: &str, uid: &str) -> Result<String, String> {
    if !blocks::ingest::dicom::is_uid(uid) {
        return Err(format!(
            "{key} {uid:?}: expected a DICOM UID (numbers joined by dots, at most 64 characters)"
        ));
    }
    Ok(uid.to_owned())
}

impl StudyQuery {
    /// Checks every key (as [`check_value`], [`check_uid`], the limit).
    pub fn check(&self) -> Result<(), String> {
        for (key, value) in [
            ("PatientName", &self.patient_name),
            ("PatientID", &self.patient_id),
            ("AccessionNumber", &self.accession_number),
            ("ModalitiesInStudy", &self.modality),
        ] {
            if let Some(v) = value {
                check_value(key, v)?;
            }
        }
        if let Some(uid) = &self.study_uid {
            check_uid("StudyInstanceUID", uid)?;
        }
        if self.limit > MAX_LIMIT {
            return Err(format!(
                "limit {}: expected 1 to {MAX_LIMIT} results",
                self.limit
            ));
        }
        Ok(())
    }

    /// The results asked for.
    pub fn limit(&self) -> u32 {
        if self.limit == 0 {
            DEFAULT_LIMIT
        } else {
            self.limit.min(MAX_LIMIT)
        }
    }

    /// The query string's pairs.
    pub fn pairs(&self) -> Vec<(&'static str, String)> {
        let mut pairs = Vec::new();
        let mut text = |key: &'static str, v: &Option<String>| {
            if let Some(v) = v {
                pairs.push((key, v.trim().to_owned()));
            }
        };
        text("PatientName", &self.patient_name);
        text("PatientID", &self.patient_id);
        text("AccessionNumber", &self.accession_number);
        text("ModalitiesInStudy", &self.modality);
        text("StudyInstanceUID", &self.study_uid);
        if let Some(d) = self.study_date {
            pairs.push(("StudyDate", d.to_query()));
        }
        for field in ["StudyDescription", "PatientBirthDate"] {
            pairs.push(("includefield", field.to_owned()));
        }
        pairs.push(("limit", self.limit().to_string()));
        if self.offset > 0 {
            pairs.push(("offset", self.offset.to_string()));
        }
        pairs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn study_dates_are_days_or_ranges() {
        let r = DateRange::parse("20050101-20051231").expect("range");
        assert_eq!((r.from, r.to), (Some(20050101), Some(20051231)));
        assert_eq!(r.to_query(), "20050101-20051231");
        assert_eq!(
            DateRange::parse("20050101").expect("day").to_query(),
            "20050101"
        );
        assert_eq!(
            DateRange::parse("-20050101").expect("open").to_query(),
            "-20050101"
        );
        assert_eq!(
            DateRange::parse("20050101-").expect("open").to_query(),
            "20050101-"
        );
        for bad in [
            "",
            "-",
            "2005",
            "20051301",
            "20050100",
            "2005-01-01",
            "20060101-20050101",
        ] {
            let err = DateRange::parse(bad).expect_err(bad);
            assert!(err.starts_with("StudyDate"), "{bad}: {err}");
        }
    }

    #[test]
    fn uids_are_numbers_joined_by_dots() {
        for good in ["1.2.840.10008.1.2", "0", "1.0.3", "1.02"] {
            assert!(check_uid("uid", good).is_ok(), "{good}");
        }
        let long = "1".repeat(65);
        for bad in ["", ".", "..", "1..2", ".1", "1.", "1.2a", long.as_str()] {
            assert!(check_uid("uid", bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn search_keys_are_checked() {
        let ok = StudyQuery {
            patient_id: Some("000-000-001".into()),
            ..StudyQuery::default()
        };
        assert!(ok.check().is_ok());
        assert!(ok.pairs().contains(&("limit", DEFAULT_LIMIT.to_string())));
        for (q, words) in [
            (
                StudyQuery {
                    patient_name: Some("a\\b".into()),
                    ..StudyQuery::default()
                },
                "PatientName",
            ),
            (
                StudyQuery {
                    study_uid: Some("1.2.abc".into()),
                    ..StudyQuery::default()
                },
                "StudyInstanceUID",
            ),
            (
                StudyQuery {
                    limit: MAX_LIMIT + 1,
                    ..StudyQuery::default()
                },
                "limit",
            ),
        ] {
            let err = q.check().expect_err(words);
            assert!(err.starts_with(words), "{err}");
        }
    }
}
